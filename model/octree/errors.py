"""The one error type raised for unusable input, so callers can catch bad data in one place."""


class OctreeInputError(ValueError):
    """Input cannot be turned into an octree; the message says what is wrong and how to fix it."""
