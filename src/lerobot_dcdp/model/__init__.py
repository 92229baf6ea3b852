"""Correctors, their networks, the completion gate, the scene lead and the pure correction math."""
