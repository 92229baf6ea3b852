"""Running the base on another machine: the served base, the robot client and the remote planner."""
