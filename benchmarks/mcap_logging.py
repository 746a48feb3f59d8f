"""Per-control-step cost of logging a run to MCAP: vectorised path against the naive one.

Run: ``PYTHONPATH=pipelines python benchmarks/mcap_logging.py [--steps N] [--repeats R]``.

Paths (all write the same six per-step topics, 100 Hz, blocks of 100 rows like the master):

* ``naive``: one protobuf object per message (``SerializeToString``), ``mcap.writer.Writer``
  ``add_message`` per message (lz4 chunks);
* ``vec-encode + Writer.add_message``: bytes from the vectorised encoder, still one
  ``add_message`` call per message (the cost of mcap's pure-Python writer alone);
* ``RunLogWriter (lz4 | zstd | none)``: the shipped path, vectorised encoding and chunks, the
  finished file fsynced before its rename (one fsync per log: a few ms, which a 30 s run
  spreads over its 3000 steps); ``no fsync``: the same without it, as batch workers write.

Times are the median of the repeats, per control step (six messages), in microseconds.
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from wmr.adapters.mcap import RunLogWriter
from wmr.adapters.mcap.schemas import STEP_TOPICS, RowEncoder, file_descriptor_set, message_class
from wmr.adapters.mcap.writer import Compression
from wmr.core.signals import COLUMN, SIGNALS

STEP_NS = 10_000_000
BLOCK = 100


def fake_run(n: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Smooth, plausible signals (compress like a real run, unlike white noise)."""
    t = np.arange(n, dtype=np.int64) * STEP_NS
    ts = t * 1e-9
    freq = np.linspace(0.05, 2.0, len(SIGNALS))
    amp = np.linspace(1.0, 30.0, len(SIGNALS))
    return t, amp * np.sin(np.outer(ts, freq)) + 0.01 * np.outer(ts, amp)


def _mcap_writer(stream: BinaryIO) -> tuple[Writer, list[int]]:
    """mcap's own writer with our schemas and one channel per step topic."""
    w = Writer(stream, compression=CompressionType.LZ4)
    w.start()
    chans = []
    for layout in STEP_TOPICS:
        sid = w.register_schema(
            layout.schema_name, "protobuf", file_descriptor_set(layout.schema_name)
        )
        chans.append(w.register_channel(layout.topic, "protobuf", sid))
    return w, chans


def naive(path: Path, t: NDArray[np.int64], x: NDArray[np.float64]) -> None:
    with open(path, "wb") as f:
        w, chans = _mcap_writer(f)
        classes = [message_class(layout.schema_name) for layout in STEP_TOPICS]
        pose_cls, tf_cls = classes[0], classes[1]
        signal_cols = [[COLUMN[s] for s in layout.signals] for layout in STEP_TOPICS]
        add = w.add_message
        for i0 in range(0, len(t), BLOCK):
            for i in range(i0, min(i0 + BLOCK, len(t))):
                ti = int(t[i])
                row = x[i].tolist()
                sec, nanos = divmod(ti, 1_000_000_000)
                half = 0.5 * row[COLUMN["theta_rad"]]
                qz, qw = math.sin(half), math.cos(half)
                pose = pose_cls(frame_id="world")
                pose.timestamp.seconds, pose.timestamp.nanos = sec, nanos
                pose.pose.position.x, pose.pose.position.y = row[0], row[1]
                pose.pose.orientation.z, pose.pose.orientation.w = qz, qw
                add(chans[0], ti, pose.SerializeToString(), ti)
                tf = tf_cls(parent_frame_id="world", child_frame_id="base_link")
                tf.timestamp.seconds, tf.timestamp.nanos = sec, nanos
                tf.translation.x, tf.translation.y = row[0], row[1]
                tf.rotation.z, tf.rotation.w = qz, qw
                add(chans[1], ti, tf.SerializeToString(), ti)
                for k in range(2, len(STEP_TOPICS)):
                    msg = classes[k]()
                    msg.timestamp.seconds, msg.timestamp.nanos = sec, nanos
                    for name, c in zip(STEP_TOPICS[k].signals, signal_cols[k], strict=True):
                        setattr(msg, name, row[c])
                    add(chans[k], ti, msg.SerializeToString(), ti)
        w.finish()


def vec_plus_writer(path: Path, t: NDArray[np.int64], x: NDArray[np.float64]) -> None:
    with open(path, "wb") as f:
        w, chans = _mcap_writer(f)
        enc = RowEncoder(tuple(chans))
        add = w.add_message
        k_topics = len(STEP_TOPICS)
        for i0 in range(0, len(t), BLOCK):
            tb = t[i0 : i0 + BLOCK]
            records, offsets = enc.encode(tb, x[i0 : i0 + BLOCK])
            ends = np.append(offsets.ravel()[1:], len(records)).tolist()
            starts = offsets.ravel().tolist()
            times = np.repeat(tb, k_topics).tolist()
            cids = chans * len(tb)
            for s, e, ti, c in zip(starts, ends, times, cids, strict=True):
                add(c, ti, records[s + 31 : e], ti)
        w.finish()


def shipped(
    compression: Compression, durable: bool = True,
) -> Callable[[Path, NDArray[np.int64], NDArray[np.float64]], None]:
    def run(path: Path, t: NDArray[np.int64], x: NDArray[np.float64]) -> None:
        with RunLogWriter(
            path,
            run={"scenario": "bench"},
            goal=(20.0, 10.0, 0.0),
            compression=compression,
            durable=durable,
        ) as w:
            for i0 in range(0, len(t), BLOCK):
                w.write_block(t[i0 : i0 + BLOCK], x[i0 : i0 + BLOCK])
            w.close({"status": "converged"})

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="control steps per run (100 Hz)")
    parser.add_argument("--repeats", type=int, default=7, help="repeats; the median is shown")
    args = parser.parse_args()
    t, x = fake_run(args.steps)
    paths: list[tuple[str, Callable[[Path, NDArray[np.int64], NDArray[np.float64]], None]]] = [
        ("naive: protobuf objects + Writer.add_message", naive),
        ("vec-encode + Writer.add_message", vec_plus_writer),
        ("RunLogWriter (lz4, default)", shipped("lz4")),
        ("RunLogWriter (lz4, no fsync, as in batches)", shipped("lz4", durable=False)),
        ("RunLogWriter (zstd)", shipped("zstd")),
        ("RunLogWriter (no compression)", shipped("")),
    ]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, fn in paths:
            path = Path(tmp) / "bench.mcap"
            runs = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                fn(path, t, x)
                runs.append((time.perf_counter() - t0) / args.steps * 1e6)
            rows.append((name, statistics.median(runs), min(runs), path.stat().st_size))
    base = rows[0][1]
    print(
        f"{args.steps} steps at 100 Hz, {len(STEP_TOPICS)} messages per step, "
        f"median of {args.repeats}"
    )
    print(f"{'path':46s} {'us/step':>9s} {'min':>8s} {'vs naive':>9s} {'file kB':>8s}")
    for name, med, best, size in rows:
        print(f"{name:46s} {med:9.2f} {best:8.2f} {med / base:9.3f} {size / 1024:8.0f}")


if __name__ == "__main__":
    main()
