"""Benchmark commands (`capsd bench ...`): each prints figures measured in one run."""
