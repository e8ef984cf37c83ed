"""The Zenoh bridge (issue 29): remote programs, telemetry and supervision."""
