"""An emulated UR controller on the loopback interface, for hardware-in-the-loop tests without a robot.

``UREmulator`` speaks what ur_rtde 1.6.5 needs (RTDE, dashboard, script upload, the control
script's register handshake) over a kinematically integrated arm; see
:mod:`snac_gym.real.emulator.protocol` for the sources the protocol was taken from.
"""

from snac_gym.real.emulator.controller import STANDARD_PORT_BASE, UREmulator

__all__ = ["STANDARD_PORT_BASE", "UREmulator"]
