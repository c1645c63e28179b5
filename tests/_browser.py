"""The headless-Chromium driver of the web-viewer tests: ``tools.bench._browser`` (the viewer bench uses it too)."""

from tools.bench._browser import (  # noqa: F401
    Browser,
    BrowserError,
    chromium_argv,
    chromium_path,
    decode_viewer_state,
    free_tcp_port,
    viewer_state,
)
