"""Where the reference STL models are: ``../shared/models`` beside the project's root.

CI runs on a clean clone with ``../shared`` beside it, so the path is taken from this file's
place, not from the machine the tests were written on.
"""

from __future__ import annotations

from pathlib import Path

MODELS = Path(__file__).resolve().parents[3] / "shared" / "models"
