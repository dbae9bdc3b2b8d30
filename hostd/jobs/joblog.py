"""The job log: one logger for every module of the job domain.

Its name is the one operators filter the journal by (``hostd.jobs.manager: job 3 'pipe3.stl':
printing -> completed``), kept when the job manager was split into its parts.
"""

from __future__ import annotations

import logging

log = logging.getLogger("hostd.jobs.manager")
