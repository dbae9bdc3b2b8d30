"""A Marlin-like firmware emulator for tests and the demo (``serial.port: sim://``).

``Firmware(settings)`` (:mod:`hostd.sim.firmware`) is the board on a simulated clock
(``receive``, ``advance``, ``settle``, ``take_output``, ``log``); ``Emulator``
(:mod:`hostd.sim.server`) drives it on the event loop with wire throttling;
``SocketEmulator.serve(settings, sock)`` puts it behind a socket; ``hostd-sim --pty`` serves it
on a pseudo-terminal. Fault knobs are in :class:`hostd.sim.settings.SimSettings`.

The package imports none of them itself: the serial link imports the settings alone, so a
hostd that drives a printer never loads the emulator.
"""

from __future__ import annotations
