"""MAVLink bridge to ArduSub (issue 6; not implemented yet)."""
