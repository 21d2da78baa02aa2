"""CAP-SD services, one package each: asv_pose, sonar_detect, locator, mav_bridge."""
