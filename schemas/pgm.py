"""Just enough of the PGM format (Netpbm greyscale) to tell a valid map image from anything else."""

from __future__ import annotations

import re
from dataclasses import dataclass

# magic, width, height, maxval, separated by whitespace and comments, then one whitespace byte
_HEADER = re.compile(rb"^(P[25])(?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)\s")


@dataclass(frozen=True)
class PgmHeader:
    magic: str
    width: int
    height: int
    maxval: int
    length: int
    """Bytes of the header itself."""

    @property
    def expected_size(self) -> int | None:
        """Total file size a binary (P5) image must have; None for plain (P2) text images."""
        if self.magic != "P5":
            return None
        return self.length + self.width * self.height * (1 if self.maxval < 256 else 2)


def read_pgm_header(data: bytes) -> PgmHeader:
    """Parse the header; raise ValueError saying what is wrong."""
    match = _HEADER.match(data[:1024])
    if match is None:
        raise ValueError("not a PGM image: it must start with P5 or P2, width, height and maxval")
    magic, width, height, maxval = match.group(1).decode(), *(int(g) for g in match.groups()[1:])
    if width < 1 or height < 1 or not 0 < maxval < 65536:
        raise ValueError(f"not a valid PGM image: {width}x{height}, maxval {maxval}")
    return PgmHeader(magic, width, height, maxval, match.end())


def check_pgm(data: bytes) -> PgmHeader:
    """A whole image: header valid and, for binary PGM, exactly as many pixel bytes as it says."""
    header = read_pgm_header(data)
    expected = header.expected_size
    if expected is not None and len(data) != expected:
        raise ValueError(
            f"PGM image of {header.width}x{header.height} should be {expected} bytes, not {len(data)}"
        )
    return header
