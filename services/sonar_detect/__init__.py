"""Sonar detection: the Oculus driver and the ROV detector (CNN, classical, the paper's box)."""
