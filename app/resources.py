"""Where the service finds the files that are not Python code: the database migrations (``alembic``),
the operator pages (``frontend``) and the example library (``models_library``).

They live at the top of the source checkout. A built wheel carries a copy of each as package data in
``app/_bundled/<name>`` (``setup.py`` puts them there), so an installed service (the Docker image,
``pip install setupcam-*.whl``) needs no checkout. A source checkout (``make run``, the tests, an
editable install) has no ``app/_bundled`` and uses the folders beside ``app/``.
"""

from __future__ import annotations

from pathlib import Path

BUNDLED = ("alembic", "frontend", "models_library")
_PACKAGE_DIR = Path(__file__).resolve().parent


def bundled_dir(name: str) -> Path:
    """The folder ``name`` (one of :data:`BUNDLED`): the wheel's copy, else the checkout's.

    Raises FileNotFoundError naming both places when neither exists (a broken install).
    """
    if name not in BUNDLED:
        raise ValueError(f"not a bundled folder: {name!r} (known: {', '.join(BUNDLED)})")
    installed = _PACKAGE_DIR / "_bundled" / name
    if installed.is_dir():
        return installed
    checkout = _PACKAGE_DIR.parent / name
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(f"setupcam's {name}/ folder is missing: looked in {installed} (installed package) "
                            f"and {checkout} (source checkout); reinstall the package")
