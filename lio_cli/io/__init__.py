"""Everything lio reads and writes: logs (``logs``), message bytes (``messages``), files that are not logs
(``files``), a log as sensor data (``sensors``). Third-party errors become ``LioError`` here."""
