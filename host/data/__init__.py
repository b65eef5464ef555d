"""Run data: the run-folder format ``tcomp-run/1`` (``runs``) and the import of logger files into it (``importer``).

The bottom room of the host's science side: everything that learns or simulates reads runs through here."""
