"""The paper's PushT experiment: rollouts of every execution mode, latency, tables, plots, videos."""
