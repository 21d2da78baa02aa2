"""Sonar detection service: Oculus driver and ROV detector (issue 5; not implemented yet)."""
