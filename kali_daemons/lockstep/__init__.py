"""The lockstep executive: every daemon of a lockstep instance in one process
(``executive``), importing the daemons it hosts by name, as the launcher starts them.
"""
