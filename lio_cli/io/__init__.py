"""Reading and writing logs and trajectory files. Third-party errors become ``LioError`` here."""
