"""LeRobot's dataset reader with its delta windows read from single-column views.

LeRobot 0.6.1 sets a custom transform on its HF dataset, and ``datasets`` >= 4.4 then fetches (and
decodes) whole rows for ``hf_dataset[key][indices]``: for a window of 24 actions, both camera
images of all 24 rows (66 PNG decodes per sample instead of 6). A ``select_columns`` view keeps
the column-wise transform and decodes only its column; the samples are identical.
Upstream fix: huggingface/lerobot#4314 (issue #4392), in no release yet; drop this once one has it.
"""

from __future__ import annotations

import torch
from lerobot.datasets.dataset_reader import DatasetReader


class ColumnViewReader(DatasetReader):
    """LeRobot's ``DatasetReader`` whose delta-window queries go through cached per-column views."""

    def _query_hf_dataset(self, query_indices: dict[str, list[int]]) -> dict:
        hf_dataset = self.hf_dataset
        assert hf_dataset is not None, "queried before the dataset was loaded"
        cached = getattr(self, "_column_views", None)
        if cached is None or cached[0] is not hf_dataset:  # (re)loaded: views of the new one
            cached = self._column_views = (hf_dataset, {})
        views = cached[1]
        result: dict = {}
        for key, q_idx in query_indices.items():
            if key in self._meta.video_keys:
                continue
            rows = (
                q_idx if self._absolute_to_relative_idx is None else [self._absolute_to_relative_idx[i] for i in q_idx]
            )
            if key not in views:
                views[key] = hf_dataset.select_columns(key)
            result[key] = torch.stack(views[key][rows][key])
        return result


def column_views(dataset) -> None:
    """Make a ``LeRobotDataset`` read its delta windows through ``ColumnViewReader``."""
    reader = dataset.reader
    if type(reader) is DatasetReader:
        reader.__class__ = ColumnViewReader
    elif not isinstance(reader, ColumnViewReader):
        raise TypeError(f"column_views: unexpected LeRobot reader {type(reader).__name__}")
