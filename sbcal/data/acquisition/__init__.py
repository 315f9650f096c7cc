"""Raw recordings of a shaker's data acquisition to bench lines: ``sbcal import`` (``docs/import.md``).

:func:`load_channel_map` reads which channels are force and base motion and where each dwell's frequency comes
from; :func:`import_recordings` reads the files (:mod:`.sources`), finds and analyses the dwells (:mod:`.dwells`)
and returns bench rows with their measured noise; :func:`write_import` writes them.
"""

from .channel_map import ChannelMap, load_channel_map
from .importer import ImportResult, import_recordings, write_import


__all__ = ["ChannelMap", "ImportResult", "load_channel_map", "import_recordings", "write_import"]
