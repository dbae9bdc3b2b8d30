"""A Marlin-like firmware emulator for tests and the demo (``serial.port: sim://``).

``Firmware(settings)`` is the board on a simulated clock (``receive``, ``advance``,
``settle``, ``take_output``, ``log``); ``Emulator`` drives it on the event loop with wire
throttling; ``SocketEmulator.serve(settings, sock)`` puts it behind a socket; ``hostd-sim
--pty`` serves it on a pseudo-terminal. Fault knobs are in :class:`SimSettings`.
"""

from __future__ import annotations

from hostd.sim.firmware import Firmware
from hostd.sim.server import Emulator, SocketEmulator
from hostd.sim.settings import SimSettings, sim_settings_from_config

__all__ = ["Emulator", "Firmware", "SimSettings", "SocketEmulator", "sim_settings_from_config"]
