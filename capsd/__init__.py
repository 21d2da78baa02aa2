"""CAP-SD shared package: payloads, keys, config, geometry, codec and the service runner."""

__version__ = "0.1.0"
