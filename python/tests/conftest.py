"""Shared fixtures of the `needle` module's tests."""

import pathlib

import pytest

#: The repository's root (python/tests/ is two levels below it).
ROOT = pathlib.Path(__file__).resolve().parents[2]

#: A coarse gel: the simple scene sets up and steps in milliseconds.
COARSE = {"gel.box.nodes": 300}


@pytest.fixture
def root():
    return ROOT
