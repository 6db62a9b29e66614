"""Shared pytest configuration: hypothesis profiles and the ``needs_gl`` fixture, which skips a
test that renders, with the reason, when no OpenGL backend works on this machine."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "default", deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True
)
settings.register_profile(
    "ci",
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
    derandomize=True,
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="session")
def needs_gl() -> str:
    """The OpenGL backend renders use; skips the test (with the reason) when none works."""
    from pipe_env.rendering import gl_backend, rendering_unavailable_reason

    reason = rendering_unavailable_reason()
    if reason is not None:
        pytest.skip(f"no OpenGL backend: {reason}")
    return gl_backend()
