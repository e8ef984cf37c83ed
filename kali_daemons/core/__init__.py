"""The shared-memory machinery every process stands on: errors, atomics and spinlocks, the
records' layout, the arena, the four channel types, real-time settings, the compiled kernels
(``csrc/``) and the cell's flat joint numbering.  Nothing here knows a robot, a board or a
process; it imports nothing else of Kali.
"""
