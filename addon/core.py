"""The one place that imports the compiled core, lazily, so the add-on registers without it."""

_core = None


def get_core():
    global _core
    if _core is None:
        try:
            from . import pathlight_core
        except ImportError as e:
            raise RuntimeError(
                "Pathlight core module is not built: run `python3 build.py build` "
                f"in the Pathlight repository ({e})"
            ) from e
        _core = pathlight_core
    return _core
