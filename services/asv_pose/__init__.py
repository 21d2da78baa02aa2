"""ASV pose: LiDAR scan matching against the walls and the IMU tilt filter."""
