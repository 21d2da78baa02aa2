"""CAP-SD: core (payloads, keys, config, codec, runner, geometry), services, simulator, tools."""

__version__ = "0.1.0"
