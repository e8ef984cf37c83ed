"""The Zenoh bridge: remote programs, telemetry and supervision."""
