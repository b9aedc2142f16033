"""Doctest namespace: every Example may use ``torch``, ``math`` and torchquat's public names."""

import math

import pytest
import torch

import torchquat

@pytest.fixture(autouse=True)
def _doctest_namespace(doctest_namespace):
    doctest_namespace["torch"] = torch
    doctest_namespace["math"] = math
    doctest_namespace["torchquat"] = torchquat
    for name in torchquat.__all__:
        doctest_namespace[name] = getattr(torchquat, name)
    torch.set_printoptions(precision=4, sci_mode=False)
