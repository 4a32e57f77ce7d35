"""activedesign SDK: API schemas, design spaces, decoding, URDF, HTTP client and CLI."""

from __future__ import annotations

__version__ = "0.1.0"
