"""Doctest namespace: every Example may use ``torch``, ``math`` and torchquat's public names."""

import math
import os

import pytest
import torch

import torchquat

# Large batches are transposed by matrix products or by copies, whichever this CPU runs faster
# (timed once per process: torchquat._planes.by_matmul). The tests fix the choice, so that the
# operations they record do not depend on the machine; tests/test_transposes.py runs the copies,
# and TORCHQUAT_TRANSPOSES=copy runs everything on them.
os.environ.setdefault("TORCHQUAT_TRANSPOSES", "matmul")


@pytest.fixture(autouse=True)
def _doctest_namespace(doctest_namespace):
    doctest_namespace["torch"] = torch
    doctest_namespace["math"] = math
    doctest_namespace["torchquat"] = torchquat
    for name in torchquat.__all__:
        doctest_namespace[name] = getattr(torchquat, name)
    torch.set_printoptions(precision=4, sci_mode=False)
