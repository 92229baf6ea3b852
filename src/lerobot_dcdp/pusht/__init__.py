"""Compatibility names: the PushT modules moved to :mod:`lerobot_dcdp.sim` and :mod:`lerobot_dcdp.data`."""
