"""The single exception type raised by the correction core."""


class CorrectionError(ValueError):
    """Invalid parameter, input or state in the force-correction core.

    Messages quote the offending value and, where there is one, the allowed range.
    """
