"""A training-batch loader for LeRobot image datasets that decodes every frame once.

LeRobot's ``DataLoader`` over a ``LeRobotDataset`` decodes each sample's PNG images again (n_obs_steps
frames x cameras per sample) and collates sample by sample: the paper profile's GPU waits on it.
``FrameLoader`` yields the same batches (keys, shapes, dtypes, values, ``*_is_pad`` flags at episode
edges) in the order of the same ``EpisodeAwareSampler``, built differently:

- every camera's frames are decoded once into a memory-mapped uint8 array (N, 3, H, W) cached in the
  dataset's folder (``.frame_cache/<digest>``), keyed by a digest of the dataset's data and info
  files (read at every start, about a second per GB): a rebuilt dataset is decoded again, never
  served stale, and trainings of several seeds on one dataset share one decode. The cache is written into a
  temporary folder and renamed into place, so a killed writer leaves nothing that is read;
- the low-dimensional columns are arrays in memory;
- a batch is one numpy gather per key over the window indices of all its samples, assembled in a
  background thread one batch ahead (pinned for CUDA), and the images become float in [0, 1] only
  on the training device.

The dataset itself stays an ordinary LeRobot dataset; nothing here writes outside ``.frame_cache``.
"""

from __future__ import annotations

import hashlib
import io
import os
import queue
import shutil
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from PIL import Image

from touch2robot.datasets import file_digest

CACHE_DIR = ".frame_cache"
# part of the cache key: a change of the cache's layout must not read old caches
CACHE_FORMAT = "frames-v1"
# LeRobot's samples hold images as ToTensor makes them: float32 uint8 / 255
IMAGE_SCALE = 255.0


def data_files(root: Path) -> list[Path]:
    """The dataset's data files in the order LeRobot concatenates them."""
    return sorted((Path(root) / "data").glob("*/*.parquet"))


def dataset_digest(root: Path) -> str:
    """Digest of a LeRobot dataset's content: its feature spec and every data file (names and bytes)."""
    root = Path(root)
    h = hashlib.sha256(CACHE_FORMAT.encode())
    for path in [root / "meta" / "info.json", *data_files(root)]:
        h.update(f"{path.relative_to(root).as_posix()}\0{file_digest(path)}\n".encode())
    return h.hexdigest()[:16]


def _decode_png(data: bytes) -> np.ndarray:
    """(3, H, W) uint8 of one stored image, the pixels LeRobot's ToTensor reads."""
    with Image.open(io.BytesIO(data)) as image:
        if image.mode != "RGB":
            raise ValueError(f"frame cache: expected RGB images, got mode {image.mode}")
        return np.asarray(image).transpose(2, 0, 1)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _write_cache(root: Path, keys: list[str], shapes: dict[str, tuple[int, ...]], frames: int, final: Path) -> None:
    """Decode every frame of ``keys`` into ``<key>.npy`` files in a temporary folder, renamed to ``final``."""
    tmp = final.with_name(f".{final.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        arrays = {
            key: np.lib.format.open_memmap(tmp / f"{key}.npy", mode="w+", dtype=np.uint8, shape=(frames, *shapes[key]))
            for key in keys
        }
        with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:  # PIL decodes without the GIL
            for path in data_files(root):
                table = pq.read_table(path, columns=["index", *keys])
                rows = table.column("index").to_numpy()
                for key in keys:
                    images = table.column(key).combine_chunks()
                    assert isinstance(images, pa.StructArray)
                    for row, image in zip(rows, pool.map(_decode_png, images.field("bytes").to_pylist()), strict=True):
                        arrays[key][row] = image
        for array in arrays.values():
            array.flush()
        del arrays
        try:
            tmp.rename(final)
        except OSError:  # another process put the same cache in place first
            if not final.is_dir():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def frame_cache(root: Path, keys: list[str], shapes: dict[str, tuple[int, ...]], frames: int) -> dict[str, np.ndarray]:
    """{image key: read-only memory map (frames, 3, H, W) uint8 by absolute frame index} of the
    dataset at ``root``, decoding the frames on the first call for this content."""
    if not keys:  # a state-only dataset: nothing to decode
        return {}
    root = Path(root)
    cache = root / CACHE_DIR
    final = cache / dataset_digest(root)
    if not final.is_dir():
        cache.mkdir(exist_ok=True)
        for leftover in cache.glob(".*.tmp"):  # a writer killed midway: never read, removed once it is gone
            pid = leftover.name.split(".")[2]
            if pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(leftover, ignore_errors=True)
        for stale in cache.iterdir():  # caches of this folder's earlier content
            if not stale.name.startswith(".") and stale.name != final.name:
                shutil.rmtree(stale, ignore_errors=True)
        _write_cache(root, keys, shapes, frames, final)
    arrays = {key: np.load(final / f"{key}.npy", mmap_mode="r") for key in keys}
    for key, array in arrays.items():
        if array.shape != (frames, *shapes[key]):
            raise ValueError(f"frame cache {final}: {key} has shape {array.shape}, expected {(frames, *shapes[key])}")
    return arrays


def _numpy_column(column: pa.ChunkedArray) -> np.ndarray:
    """A column as LeRobot's ``torch.tensor`` makes it: floats float32, integers int64, lists as rows."""
    values = column.combine_chunks()
    if pa.types.is_fixed_size_list(values.type) or pa.types.is_list(values.type):
        flat = values.flatten().to_numpy(zero_copy_only=False)
        array = flat.reshape(len(values), -1)
    else:
        array = values.to_numpy(zero_copy_only=False)
    if np.issubdtype(array.dtype, np.floating):
        return array.astype(np.float32)
    if np.issubdtype(array.dtype, np.bool_):
        return array
    return array.astype(np.int64)


class FrameLoader:
    """Batches of a ``LeRobotDataset`` (all episodes) in the order of ``sampler``, equal to those of
    ``DataLoader(dataset, batch_size, sampler=sampler, drop_last=False)`` with LeRobot's collation;
    tensors on ``device``. Each ``iter()`` is one epoch of the sampler (which advances it)."""

    def __init__(self, dataset, sampler, batch_size: int, device: torch.device | str = "cpu") -> None:
        if dataset.episodes is not None:
            raise ValueError("FrameLoader reads whole datasets (episodes=None)")
        meta = dataset.meta
        self.sampler = sampler
        self.batch_size = batch_size
        self.device = torch.device(device)
        self.image_keys = list(meta.camera_keys)
        if meta.video_keys:
            raise ValueError(f"FrameLoader reads image datasets; {dataset.repo_id} stores video {meta.video_keys}")
        frames = meta.total_frames
        # LeRobot's image features are (H, W, C); its samples are (C, H, W)
        shapes = {k: tuple(meta.features[k]["shape"][i] for i in (2, 0, 1)) for k in self.image_keys}
        self.images = frame_cache(dataset.root, self.image_keys, shapes, frames)
        columns = [k for k in meta.features if k not in self.image_keys]
        table = pa.concat_tables(pq.read_table(p, columns=columns) for p in data_files(dataset.root))
        order = np.argsort(table.column("index").to_numpy())
        self.columns = {k: _numpy_column(table.column(k))[order] for k in columns}
        if not np.array_equal(self.columns["index"], np.arange(frames)):
            raise ValueError(f"{dataset.root}: frame indices are not 0..{frames - 1}")
        episodes = meta.episodes
        starts = np.asarray(episodes["dataset_from_index"], dtype=np.int64)
        ends = np.asarray(episodes["dataset_to_index"], dtype=np.int64)
        episode = self.columns["episode_index"]
        self.episode_start, self.episode_end = starts[episode], ends[episode]
        self.deltas = {k: np.asarray(d, dtype=np.int64) for k, d in (dataset.reader.delta_indices or {}).items()}
        self.tasks = [str(name) for name in meta.tasks.index]
        # a device tensor: CUDA divides by a CPU scalar through its reciprocal, one bit off LeRobot's images
        self._scale = torch.tensor(IMAGE_SCALE, dtype=torch.float32, device=self.device)

    def __len__(self) -> int:
        return -(-len(self.sampler) // self.batch_size)

    def host_batch(self, indices) -> dict:
        """The batch of frames ``indices`` on the host, images still uint8 (B, [K,] 3, H, W)."""
        idx = np.asarray(indices, dtype=np.int64)
        batch: dict = {}
        for key, values in self.columns.items():
            if key in self.deltas:
                continue
            batch[key] = torch.from_numpy(values[idx])
        pads: dict = {}
        for key, delta in self.deltas.items():
            wanted = idx[:, None] + delta[None, :]
            start, end = self.episode_start[idx, None], self.episode_end[idx, None]
            window = np.clip(wanted, start, end - 1)
            source = self.images[key] if key in self.images else self.columns[key]
            batch[key] = torch.from_numpy(np.ascontiguousarray(source[window]))
            pads[f"{key}_is_pad"] = torch.from_numpy((wanted < start) | (wanted >= end))
        for key in self.image_keys:
            if key not in batch:
                batch[key] = torch.from_numpy(np.ascontiguousarray(self.images[key][idx]))
        batch.update(pads)
        batch["task"] = [self.tasks[t] for t in self.columns["task_index"][idx]]
        return batch

    def to_device(self, batch: dict) -> dict:
        """``batch`` on the device with its images float32 in [0, 1], as LeRobot's samples hold them."""
        out = {}
        for key, value in batch.items():
            if isinstance(value, torch.Tensor):
                value = value.to(self.device, non_blocking=True)
                if key in self.images:
                    value = value.to(torch.float32).div_(self._scale)
            out[key] = value
        return out

    def _produce(self, batches: list[list[int]], ready: queue.Queue, stop: threading.Event) -> None:
        def hand_over(item) -> bool:
            while not stop.is_set():
                try:
                    ready.put(item, timeout=0.1)
                    return True
                except queue.Full:
                    continue
            return False

        pin = self.device.type == "cuda"
        try:
            for indices in batches:
                host = self.host_batch(indices)
                if pin:
                    host = {k: v.pin_memory() if isinstance(v, torch.Tensor) else v for k, v in host.items()}
                if not hand_over(host):
                    return
        except BaseException as error:  # handed to the consumer, which raises it
            hand_over(error)

    def __iter__(self) -> Iterator[dict]:
        # DataLoader draws a seed from torch's RNG per epoch; drawing it too keeps the training's
        # random crops and noise the same whichever loader feeds it
        torch.empty((), dtype=torch.int64).random_()
        order = list(iter(self.sampler))
        batches = [order[i : i + self.batch_size] for i in range(0, len(order), self.batch_size)]
        return self._epoch(batches)

    def _epoch(self, batches: list[list[int]]) -> Iterator[dict]:
        ready: queue.Queue = queue.Queue(maxsize=2)
        stop = threading.Event()
        worker = threading.Thread(target=self._produce, args=(batches, ready, stop), daemon=True)
        worker.start()
        try:
            for _ in batches:
                host = ready.get()
                if isinstance(host, BaseException):
                    raise host
                yield self.to_device(host)
        finally:
            stop.set()
            worker.join()
