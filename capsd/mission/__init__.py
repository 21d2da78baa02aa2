"""ROV missions on CAP-SD fixes: plans in tank coordinates, the mission logic, its report."""
