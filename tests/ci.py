"""What a test does where something it needs is missing: skip here, fail in CI.

CI (``CI`` set, as ``.ci/run`` does) installs everything the tests use (ParaView, Xvfb, Mesa's
OpenGL), so a test that would skip there has lost what it tests.
"""

import os

import pytest


def unavailable(reason: str) -> None:
    """Skip the calling test, saying ``reason``; in CI, fail it instead."""
    if os.environ.get("CI"):
        pytest.fail(f"CI must run this test: {reason}", pytrace=False)
    pytest.skip(reason)
