"""The one exception type of force_tester_sim."""


class SimError(ValueError):
    """A bad parameter, test set, pull specification or simulation request.

    Messages quote the offending value and what was expected.
    """
