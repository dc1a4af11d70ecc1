"""Schemathesis hooks: what the OpenAPI document cannot say about a body.

The binary body of POST /tilesets/{name}/heights is a run of points, each two finite
little-endian f64 (16 bytes); `format: binary` cannot express that, so schemathesis would call
any byte string "schema-valid" and flag the server's 400 for a 15-byte body as a rejected valid
request. Bodies of application/octet-stream are drawn here as such point runs. The other
octet-stream body (POST /tilesets, a raster upload) is answered 202 whatever its bytes are, so
it is unaffected. Negative cases (malformed bodies) are still tried by schemathesis's own
negative generation and by tests/heights.rs.
"""

import struct

import schemathesis
from hypothesis import strategies as st

_coord = st.floats(allow_nan=False, allow_infinity=False, width=64)
_points = st.lists(st.tuples(_coord, _coord), max_size=64)

schemathesis.openapi.media_type(
    "application/octet-stream",
    _points.map(lambda pts: b"".join(struct.pack("<dd", x, y) for x, y in pts)),
)
