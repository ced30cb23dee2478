"""The single exception type of force_discovery."""


class DiscoveryError(ValueError):
    """Data discovery cannot analyse: the message quotes the offending value and what was expected."""
