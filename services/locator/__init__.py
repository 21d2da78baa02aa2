"""Locator: turns sonar detections, the ASV pose and the ROV's depth into ROV fixes."""
