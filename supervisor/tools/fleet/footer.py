"""A Parquet file's footer checked before pyarrow is given it: pyarrow's metadata
calls have no C++ exception handling, so an enum value out of its range (a codec, an
encoding, a type) ends the whole process (``std::terminate``, SIGABRT) where it should
raise.  A dataset's file is anybody's input (docs/reference/fleet.md, "fleet report",
its bounds): its footer is walked here first, in Thrift's compact protocol as the
Parquet format defines it (github.com/apache/parquet-format, ``parquet.thrift``), and
each enum pyarrow converts is checked against the values the format knows, and each
column's level histograms against its schema.  Fields it does not know are skipped,
as a reader of a newer writer's file must; encryption is refused, as fleet replay
never writes it.
"""

from __future__ import annotations

MAGIC = b"PAR1"
MAX_FOOTER = 16 << 20  # a row file's is a few kB; a violations file's grows with its row groups
MAX_DEPTH = 32  # the format nests a few levels (a logical type's unit in a column's schema)

# compact protocol types
_STOP, _TRUE, _FALSE, _BYTE, _I16, _I32, _I64, _DOUBLE, _BINARY = range(9)
_LIST, _SET, _MAP, _STRUCT = 9, 10, 11, 12

# parquet.thrift's enums: the values a field may hold, by (struct, field id)
_TYPE = range(8)  # Type: BOOLEAN .. FIXED_LEN_BYTE_ARRAY
_ENCODING = range(10)  # Encoding: PLAIN .. BYTE_STREAM_SPLIT
_CODEC = range(8)  # CompressionCodec: UNCOMPRESSED .. LZ4_RAW
_PAGE = range(4)  # PageType: DATA_PAGE .. DATA_PAGE_V2
_REPETITION = range(3)  # FieldRepetitionType: REQUIRED, OPTIONAL, REPEATED
_CONVERTED = range(22)  # ConvertedType: UTF8 .. INTERVAL
_INT_WIDTHS = (8, 16, 32, 64)  # IntType's bitWidth

# the structs walked, each field's own struct (a struct, or a list of them) and enum
FILE, SCHEMA, ROW_GROUP, COLUMN, META, ENC_STATS = "file", "schema", "rg", "col", "meta", "es"
SIZE_STATS = "size statistics"
LOGICAL, TIME_UNIT, INT_TYPE, TIMED, OTHER = "logical", "unit", "int", "timed", "other"
_STRUCTS = {
    (FILE, 2): SCHEMA,
    (FILE, 4): ROW_GROUP,
    (SCHEMA, 10): LOGICAL,
    (ROW_GROUP, 1): COLUMN,
    (COLUMN, 3): META,
    (META, 13): ENC_STATS,
    (META, 16): SIZE_STATS,
    (LOGICAL, 7): TIMED,  # TimeType
    (LOGICAL, 8): TIMED,  # TimestampType
    (LOGICAL, 10): INT_TYPE,
    (TIMED, 2): TIME_UNIT,
}
_ENUMS = {
    (SCHEMA, 1): _TYPE,
    (SCHEMA, 3): _REPETITION,
    (SCHEMA, 6): _CONVERTED,
    (META, 1): _TYPE,
    (META, 2): _ENCODING,
    (META, 4): _CODEC,
    (ENC_STATS, 1): _PAGE,
    (ENC_STATS, 2): _ENCODING,
}
# the kinds the fields whose values are checked, or recorded, must be
_KINDS = {
    **{where: {_I32} for where in _ENUMS if where not in ((META, 2),)},
    (META, 2): {_LIST},
    (SCHEMA, 5): {_I32},
    (FILE, 2): {_LIST},
    (FILE, 4): {_LIST},
    (ROW_GROUP, 1): {_LIST},
    (COLUMN, 3): {_STRUCT},
    (META, 13): {_LIST},
    (META, 16): {_STRUCT},
    (SIZE_STATS, 2): {_LIST},
    (SIZE_STATS, 3): {_LIST},
}
# LogicalType and TimeUnit are unions: the member's field id is what is read
_MEMBERS = {LOGICAL: {*range(1, 9), *range(10, 19)}, TIME_UNIT: {1, 2, 3}}
_REFUSED = {(FILE, 8): "encrypted", (FILE, 9): "encrypted", (COLUMN, 8): "encrypted",
            (COLUMN, 9): "encrypted"}  # fmt: skip


class BadFooter(Exception):
    """Why the footer is no file fleet replay writes."""


def footer_length(size: int, tail: bytes) -> int | None:
    """The length of the footer of a file of ``size`` bytes whose last 8 are ``tail``
    (the footer's length, then ``PAR1``); None where there is none to read (pyarrow
    then says why); ``BadFooter`` for one too large to walk, never given unwalked."""
    if size < 12 or len(tail) != 8 or tail[4:] != MAGIC:
        return None
    n = int.from_bytes(tail[:4], "little")
    if n > size - 12:
        return None
    if n > MAX_FOOTER:
        raise BadFooter(f"its footer is over {MAX_FOOTER >> 20} MB")
    return n


def check(footer: bytes) -> None:
    """``BadFooter`` if the footer is damaged or holds a value pyarrow cannot take."""
    walker = _Walker(footer)
    walker.struct(FILE, 0)
    walker.flat()


class _Walker:
    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0
        # what the levels' histograms must agree with: each schema element's
        # repetition and children, and each column chunk's histograms' lengths
        self.elements: list[dict[int, int]] = []
        self.chunks: list[dict[int, int]] = []
        self.groups: list[int] = []

    def flat(self) -> None:
        """The schema is a root of plain columns, as fleet replay writes it, and each
        column chunk's level histograms are as long as its column's levels make them
        (pyarrow aborts on another length)."""
        if not self.elements:
            raise BadFooter("its footer has no schema")
        root, leaves = self.elements[0], self.elements[1:]
        if root.get(5) != len(leaves) or any(e.get(5, 0) for e in leaves):
            raise BadFooter("its footer's schema is not a table of plain columns")
        if any(n != len(leaves) for n in self.groups):
            raise BadFooter("its footer's row groups do not hold each column once")
        if len(self.chunks) != sum(self.groups):
            raise BadFooter("its footer has a column chunk without its metadata")
        for i, chunk in enumerate(self.chunks):
            repetition = leaves[i % len(leaves)].get(3)
            if repetition is None:
                raise BadFooter("its footer has a column of no repetition")
            definitions = 2 if repetition != 0 else 1  # optional or repeated: 0 and 1
            repetitions = 2 if repetition == 2 else 1
            if chunk.get(3, 0) not in (0, definitions) or chunk.get(2, 0) not in (
                0,
                repetitions,
            ):
                raise BadFooter("its footer has level histograms of the wrong length")

    def byte(self) -> int:
        if self.at >= len(self.data):
            raise BadFooter("its footer ends early")
        b = self.data[self.at]
        self.at += 1
        return b

    def varint(self) -> int:
        n = shift = 0
        while True:
            b = self.byte()
            n |= (b & 0x7F) << shift
            if not b & 0x80:
                return n
            shift += 7
            if shift > 63:
                raise BadFooter("its footer has a number too long")

    def zigzag(self) -> int:
        n = self.varint()
        return (n >> 1) ^ -(n & 1)

    def skip(self, size: int) -> None:
        if size < 0 or self.at + size > len(self.data):
            raise BadFooter("its footer ends early")
        self.at += size

    def struct(self, kind: str, depth: int) -> None:
        if depth > MAX_DEPTH:
            raise BadFooter("its footer nests too deep")
        if kind == SCHEMA:
            self.elements.append({})
        elif kind == ROW_GROUP:
            self.groups.append(0)
        elif kind == COLUMN:
            self.groups[-1] += 1
        elif kind == META:
            self.chunks.append({})
        field = 0
        members = 0
        while True:
            head = self.byte()
            kind_ = head & 0x0F
            if kind_ == _STOP:
                break
            delta = head >> 4
            field = field + delta if delta else self.zigzag()
            where = (kind, field)
            if where in _REFUSED:
                raise BadFooter(f"its footer says it is {_REFUSED[where]}")
            members += 1
            if kind in _MEMBERS and field not in _MEMBERS[kind]:
                raise BadFooter(f"its footer has an unknown {kind} type ({field})")
            if where in _KINDS and kind_ not in _KINDS[where]:
                # a thrift reader skips a field of another kind: left unset, it is
                # what pyarrow aborts on
                raise BadFooter(f"its footer has a {_NAMES.get(where, kind)} of another kind")
            got = self.value(kind_, _STRUCTS.get(where, OTHER), _ENUMS.get(where), depth, where)
            if kind == SCHEMA and field in (3, 5):
                self.elements[-1][field] = got
            elif kind == SIZE_STATS and field in (2, 3):
                self.chunks[-1][field] = got
        if kind in _MEMBERS and members != 1:
            raise BadFooter(f"its footer has a {kind} of {members} types")

    def value(
        self, kind: int, struct: str, enum: range | None, depth: int, where: tuple[str, int]
    ) -> int:
        """Reads one value; an integer's value, a list's or set's size, else 0."""
        if kind in (_TRUE, _FALSE):
            return 0
        if kind == _BYTE:
            b = self.byte()
            if where == (INT_TYPE, 1) and b not in _INT_WIDTHS:
                raise BadFooter(f"its footer has an integer of {b} bits")
            return b
        if kind in (_I16, _I32, _I64):
            n = self.zigzag()
            if enum is not None and n not in enum:
                raise BadFooter(f"its footer has an unknown {_NAMES[where]} ({n})")
            return n
        if kind == _DOUBLE:
            self.skip(8)
        elif kind == _BINARY:
            self.skip(self.varint())
        elif kind in (_LIST, _SET):
            head = self.byte()
            size = head >> 4
            if size == 15:
                size = self.varint()
            item = head & 0x0F
            if size > len(self.data) - self.at and item not in (_TRUE, _FALSE):
                raise BadFooter("its footer ends early")  # each item takes a byte at least
            for _ in range(size):
                if item in (_TRUE, _FALSE):
                    self.byte()  # a list's bool is a byte of its own
                else:
                    self.value(item, struct, enum, depth + 1, where)
            return size
        elif kind == _MAP:
            size = self.varint()
            if size:
                types = self.byte()
                if 2 * size > len(self.data) - self.at:
                    raise BadFooter("its footer ends early")
                for _ in range(size):
                    self.value(types >> 4, OTHER, None, depth + 1, where)
                    self.value(types & 0x0F, OTHER, None, depth + 1, where)
        elif kind == _STRUCT:
            self.struct(struct, depth + 1)
        else:
            raise BadFooter(f"its footer has a value of unknown kind {kind}")
        return 0


_NAMES = {
    (SCHEMA, 1): "type",
    (SCHEMA, 3): "repetition",
    (SCHEMA, 6): "converted type",
    (META, 1): "type",
    (META, 2): "encoding",
    (META, 4): "compression codec",
    (ENC_STATS, 1): "page type",
    (ENC_STATS, 2): "encoding",
}
