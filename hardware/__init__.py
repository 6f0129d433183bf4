"""Device contracts and the real rig: ZED over UVC, proportional valves over serial.

Importing this package loads only the contracts; the drivers are imported by name
(``hardware.zed``, ``hardware.valves``) so a simulated run never touches a serial port.
"""

from hardware.errors import DeviceError, LinkLostError, NotConnectedError
from hardware.interfaces import StereoCamera, StereoFrame, ValveBank

__all__ = ["DeviceError", "LinkLostError", "NotConnectedError", "StereoCamera", "StereoFrame", "ValveBank"]
