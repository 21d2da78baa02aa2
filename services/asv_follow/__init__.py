"""The ASV follower: keeps the ROV inside the sonar's view by moving the ASV (GUIDED targets)."""
