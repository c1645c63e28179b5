"""The headless-Chromium driver of the web-viewer tests: ``tools.bench._browser`` (the viewer bench uses it too)."""

from tools.bench._browser import Browser, BrowserError, chromium_argv, chromium_path, free_tcp_port  # noqa: F401
