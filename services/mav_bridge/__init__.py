"""MAVLink bridge: CAP-SD fixes to ArduSub as vision-position estimates, through a safety gate."""
