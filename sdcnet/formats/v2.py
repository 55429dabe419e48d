"""The Open Inference Protocol's binary tensor data extension (KServe, Triton), as the service
(``sdcnet.service.v2``) and the client (``sdcnet.client.protocol``) both speak it: a JSON
header whose length travels in an HTTP header, then each binary tensor's raw little-endian
bytes."""

from __future__ import annotations

import numpy as np

#: HTTP header: the JSON header's length, bytes, when binary data follows it.
HEADER_LENGTH = "Inference-Header-Content-Length"
#: numpy type of each datatype sdcnet's tensors use; binary data is little-endian.
DTYPES = {
    "UINT8": np.dtype("u1"),
    "UINT16": np.dtype("<u2"),
    "FP16": np.dtype("<f2"),
    "FP32": np.dtype("<f4"),
}
