"""The one error tree of devices. A person can act on every one of them (plug the device in, check the URL,
resume), so they are InputErrors: the CLI prints one line, never a traceback.

    InputError (geometry.errors)
    └── DeviceError             a device failed in a way a person must look at
        ├── DeviceTimeoutError    no valid answer after every retry
        ├── DeviceRefusedError    the device refused a request or reported impossible values (GrblError,
        │                         ScannerError)
        └── recovered inside a driver (one escapes only when a driver's own retries are used up):
            ├── FrameTimeoutError   no complete frame before a read's deadline
            ├── DisconnectedError   the transport went away, or could not be opened
            ├── DeviceResetError    the device was reset or reconnected: the state it held is lost, redo the step
            └── RequestDamagedError the device says our request arrived damaged: send it again
"""

from geometry.errors import InputError


class DeviceError(InputError):
    """A device could not be opened or reached, answered wrongly, or did not do what it was told."""


class DeviceTimeoutError(DeviceError):
    """A device did not answer within its timeout, after every retry."""


class DeviceRefusedError(DeviceError):
    """The device refused a request (an error code, an alarm) or reported values it cannot have."""


class FrameTimeoutError(DeviceError):
    """No complete frame arrived before the deadline (recoverable: the exchange sends the request again)."""


class DisconnectedError(DeviceError):
    """The transport went away or could not be opened (recoverable: reconnect, then the protocol resynchronises)."""


class DeviceResetError(DeviceError):
    """The device was reset or reconnected: state (position, buffers) was lost; redo the current step."""


class RequestDamagedError(DeviceError):
    """The device says our request arrived damaged: `exchange()` sends it again."""
