"""The ``record:`` section: where and how the daemon records its inputs into rosbag2
MCAP bags (docs/reference/config.md, record).

Recording is on when ``run --record DIR`` is given or ``record.path`` is set; the
other keys bound what the recording may cost: disk (``max_bag_mb`` x ``keep``) and
memory (``queue_messages`` waiting for the writer process).
"""

from __future__ import annotations

from dataclasses import dataclass

from supervisor.config.fields import as_mapping, check_keys, error_at, number, whole_number
from supervisor.config.yamlload import LineDict

RECORD_KEYS = {"path", "max_bag_mb", "max_bag_s", "keep", "queue_messages"}
MB = 1 << 20
# A bag of 1 TB or one open for 11.6 days is a typo, not a plan: rotation exists so
# that an old bag can be deleted while the daemon runs.
MAX_BAG_MB = 1e6
MAX_BAG_S = 1e6
MAX_KEEP = 1_000_000
# At ~100 bytes a message in memory, 10 million is about 1 GB: still bounded.
MAX_QUEUE = 10_000_000


@dataclass(frozen=True)
class RecordConfig:
    # The directory the bags go into; None: only ``run --record DIR`` turns recording on.
    path: str | None = None
    # A bag is closed and the next one begun at this size or age, whichever comes
    # first; keep x max_bag_mb bounds the disk the recording takes.
    max_bag_mb: float = 100.0
    max_bag_s: float = 300.0
    keep: int = 20
    # Messages waiting for the writer process; beyond it new ones are dropped and
    # counted (the receive loop never waits for the disk). 5 s at 20k msg/s.
    queue_messages: int = 100_000
    line: int | None = None  # of 'record:'

    @property
    def max_bag_bytes(self) -> int:
        return max(1, int(self.max_bag_mb * MB))


def load_record(doc: LineDict) -> RecordConfig | None:
    """The ``record:`` section, or None when the config has none."""
    raw = doc.get("record")
    if raw is None:
        return None
    s = as_mapping(raw, doc, "record", "record")
    check_keys(s, RECORD_KEYS, "record")
    path = s.get("path")
    if path is not None and (not isinstance(path, str) or not path.strip()):
        raise error_at("record.path must be a directory path", s, "path")
    defaults = RecordConfig()
    max_bag_mb = number(s, "max_bag_mb", "record", maximum=MAX_BAG_MB)
    max_bag_s = number(s, "max_bag_s", "record", maximum=MAX_BAG_S)
    return RecordConfig(
        path=path,
        max_bag_mb=defaults.max_bag_mb if max_bag_mb is None else max_bag_mb,
        max_bag_s=defaults.max_bag_s if max_bag_s is None else max_bag_s,
        keep=whole_number(s, "keep", "record", default=defaults.keep, minimum=1, maximum=MAX_KEEP),
        queue_messages=whole_number(
            s,
            "queue_messages",
            "record",
            default=defaults.queue_messages,
            minimum=1,
            maximum=MAX_QUEUE,
        ),
        line=doc.key_line("record"),
    )
