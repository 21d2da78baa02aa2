"""The simulated tank: world, vehicles and sensors, for dry runs, tests and benchmarks."""
