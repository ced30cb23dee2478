"""The single exception type of the monitor package."""


class MonitorError(ValueError):
    """Invalid parameter, input or state in the monitor; the message quotes the offending value and
    what was expected (a port in use names the port)."""
