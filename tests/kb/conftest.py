"""Fixtures of the knowledge-base tests: the files in tests/data/kb."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.kb import KnowledgeBase

KB_DATA = Path(__file__).resolve().parents[1] / "data" / "kb"
WAREHOUSE = KB_DATA / "warehouse.rddl"
TURTLEBOT_DOMAIN = KB_DATA / "turtlebot_printing_domain.rddl"
TURTLEBOT_INSTANCE = KB_DATA / "turtlebot_printing_instance.rddl"


@pytest.fixture
def warehouse() -> KnowledgeBase:
    """The hand-written test domain (domain, non-fluents and instance in one file)."""
    return KnowledgeBase.from_files(WAREHOUSE, WAREHOUSE)


@pytest.fixture
def turtlebot() -> KnowledgeBase:
    """ROSPlan's print-fetching domain and its bhn7 instance, as tests/data/kb has them."""
    return KnowledgeBase.from_files(TURTLEBOT_DOMAIN, TURTLEBOT_INSTANCE)
