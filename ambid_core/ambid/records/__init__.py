"""External time records: a rig's own logs in (CSV, MAT v5/v7.3, NPZ) and a session's records out.

- :mod:`.readers`: open a record and read its channels in row chunks (memory flat in file length).
- :mod:`.writers`: write channels in those formats, atomically.
- :mod:`.mapping`: MAP.yaml, which channel is what (column, scale, unit).
- :mod:`.importer`: a record and its map become a session in the recorder's MCAP layout.
- :mod:`.exporter`: a session's time records and their MAP.yaml.
"""

from .readers import CHUNK_ROWS, FORMATS, Record, RecordError, open_record, open_records, record_format
from .writers import WRITE_FORMATS, atomic_path, write_record

__all__ = ["CHUNK_ROWS", "FORMATS", "WRITE_FORMATS", "Record", "RecordError", "atomic_path", "open_record",
           "open_records", "record_format", "write_record"]
