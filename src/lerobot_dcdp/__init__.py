"""DCDP for LeRobot: closed-loop action chunks with per-step corrections of a frozen chunking policy.

Layers, each importing only those below it (``lint-imports`` checks this; see pyproject.toml):

- ``benchmark``: rollouts, tables, latency, the demo;
- ``train``: completion-gate fit, residual RL (PPO);
- ``deploy``: served base, robot client, remote planner;
- ``data``: demonstrations, recorded corrections, DAgger / plan converters, FastUMI, atomic folders;
- ``sim``: the perturbed PushT env, the simulated robot, teleoperators, the scripted expert;
- ``policy``: LeRobot's face (config, ``DCDPPolicy``, processors, folders, base loading);
- ``runtime``: execution modes, planning, chunk sources, the compiled step kernel;
- ``model``: correctors, their networks, gate, scene lead and the pure correction math.

Importing this package registers nothing; ``lerobot_policy_dcdp`` (what LeRobot's plugin discovery imports)
registers the ``dcdp`` policy, its processor steps, the ``pusht_perturbed`` env, the ``pusht_sim`` robot and
the ``pusht_expert`` / ``pusht_nudge`` teleoperators.
"""
