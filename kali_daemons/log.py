"""Reading a recording back where programs import it (``from kali_daemons import log``); it
lives in ``recording.log``, beside the recorder."""

from .recording.log import ArmLog, Log, ServoChange, TruthLog, read

__all__ = ["ArmLog", "Log", "ServoChange", "TruthLog", "read"]
