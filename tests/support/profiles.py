"""How much the property and bulk tests run: the full suite runs Hypothesis's ``thorough``
profile (its default settings); ``make test-fast`` loads ``quick`` (``--hypothesis-profile
quick``), a tenth of the examples and of the seeded bulk cases, for the edit loop."""
from __future__ import annotations

from hypothesis import settings

QUICK_SHARE = 10
"""The quick profile runs this much less."""

settings.register_profile("thorough", settings.get_profile("default"))
settings.register_profile("quick", max_examples=max(1, settings.get_profile("default").max_examples // QUICK_SHARE))


def scaled(n: int) -> int:
    """``n`` examples or cases under the thorough profile, a tenth of them (at least 1) under
    the quick one."""
    return max(1, n // QUICK_SHARE) if settings.get_current_profile_name() == "quick" else n
