"""ConvertRotation: a picklable dataset transform that works in DataLoader workers."""

import pickle

import pytest
import torch
from torch.utils.data import DataLoader, Dataset

import torchquat
from torchquat.io import ConvertRotation


class QuatDataset(Dataset):
    def __init__(self, transform):
        self.q = torchquat.random_quat((16,), generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        self.transform = transform

    def __len__(self):
        return len(self.q)

    def __getitem__(self, i):
        return self.transform({"rotation": self.q[i], "index": i})


def test_transform_converts_dict_key_and_plain_tensor():
    q = torchquat.random_quat((5,), dtype=torch.float64)
    to_matrix = ConvertRotation("quat", "matrix")
    torch.testing.assert_close(to_matrix(q), torchquat.quat_to_matrix(q))
    sample = to_matrix({"rotation": q, "label": "a"})
    assert sample["label"] == "a" and sample["rotation"].shape == (5, 3, 3)


def test_transform_survives_pickling():
    t = ConvertRotation("euler", "quat", convention="ZYX", degrees=True)
    clone = pickle.loads(pickle.dumps(t))
    angles = torch.tensor([30.0, 10.0, -5.0], dtype=torch.float64)
    torch.testing.assert_close(clone(angles), t(angles))


def test_transform_runs_in_two_dataloader_workers():
    dataset = QuatDataset(ConvertRotation("quat", "rot6d"))
    loader = DataLoader(dataset, batch_size=4, num_workers=2)
    batches = list(loader)
    rot6d = torch.cat([b["rotation"] for b in batches])
    expected = torchquat.convert(dataset.q, "quat", "rot6d")
    torch.testing.assert_close(rot6d, expected)
    assert torch.cat([b["index"] for b in batches]).tolist() == list(range(16))


@pytest.mark.parametrize("options,message", [({"convention": "ZYX"}, "convention='ZYX' only applies to Euler angles"),
                                             ({"degrees": True}, "degrees=True only applies to Euler angles")])
def test_options_that_would_be_ignored_are_refused_as_by_the_convert_layer(options, message):
    # ConvertRotation("quat", "matrix", degrees=True) was accepted and did nothing (Convert refuses it)
    with pytest.raises(ValueError, match="ConvertRotation: " + message):
        ConvertRotation("quat", "matrix", **options)
