"""MJCF assets authored for this project (installed as package data)."""

from pathlib import Path

ASSETS_DIR: Path = Path(__file__).resolve().parent
PANDA_XML: Path = ASSETS_DIR / "panda" / "panda.xml"
