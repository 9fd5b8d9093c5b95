"""Host-side device driver for the north finder and the wire codec it shares with the simulator.

``driver`` imports neither ``host`` nor ``firmware_sim``.
"""
