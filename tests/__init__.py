"""The test suite; its folders mirror the packages (docs/tests.md, "Layout")."""
