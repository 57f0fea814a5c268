"""Errors of devices: a person can act on them (plug the head in, check the URL), so they are InputErrors."""

from geometry.errors import InputError


class DeviceError(InputError):
    """A device could not be opened, answered wrongly, or did not do what it was told."""


class DeviceTimeoutError(DeviceError):
    """A device did not answer within its timeout, after every retry."""
