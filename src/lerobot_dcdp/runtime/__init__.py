"""What happens at a control step: execution modes, planning, planners, chunk sources, the step kernel."""
