"""Test-wide settings.

CasADi Functions run in-process (``AEROMANIP_CODEGEN=0``) unless a test is about compiled
code (marker ``codegen``): the answers are the same, and the suite tests rather than
compiles. ``AEROMANIP_CODEGEN=1 python -m pytest`` runs every test on compiled code.
"""

import os

import pytest

os.environ.setdefault("AEROMANIP_CODEGEN", "0")


def pytest_configure(config):
    config.addinivalue_line("markers", "codegen: the test builds C code (codegen on for it)")


@pytest.fixture(autouse=True)
def _codegen_for_marked_tests(request, monkeypatch):
    if request.node.get_closest_marker("codegen"):
        monkeypatch.setenv("AEROMANIP_CODEGEN", "1")
