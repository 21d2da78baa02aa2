"""ASV pose service: LiDAR scan matching and IMU tilt filter (issue 9; not implemented yet)."""
