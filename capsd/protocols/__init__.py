"""Device protocols as bytes (Oculus, SICK CoLa-A) and the one typed MAVLink adapter.

Shared by the drivers in services and the device fakes in the simulator.
"""
