"""Servo algorithms: what one declares (``algorithm``), the registry of them by name with the
plugins (``registry``), the built-in joint servos (``builtins``, ``vector``) and robot-level
ones (``arm``, ``armbuiltins``, ``admittance``).  A library under the runtime: the config
checks plugins against it; ``kali_daemons.servo`` re-exports what a plugin imports.
"""
