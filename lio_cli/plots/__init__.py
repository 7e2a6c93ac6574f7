"""Every picture lio draws (matplotlib is imported only here, and only when a picture is asked for)."""
