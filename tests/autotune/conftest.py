from __future__ import annotations

import pytest

from tests.postgres import postgres_server


@pytest.fixture(scope="session")
def postgres_url():
    """URL of a local PostgreSQL server started for the test session (skips without one)."""
    with postgres_server() as url:
        yield url
