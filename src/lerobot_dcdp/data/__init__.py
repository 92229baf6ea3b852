"""Datasets: PushT demonstrations, recorded corrections, DAgger and plan converters, FastUMI, atomic
folders."""
