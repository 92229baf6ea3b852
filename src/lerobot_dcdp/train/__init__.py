"""Training beyond stage 1: the completion-gate fit and residual RL (PPO) over a frozen base."""
