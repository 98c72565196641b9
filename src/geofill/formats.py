"""The output formats a user can name (``geofill batch --format``) and the file extension each
writes. Kept free of imports so that the command line builds its parser without loading the image
libraries; the encoders' settings are in :mod:`geofill.io.output`."""

#: ``--format`` name -> extension of the files written in that format.
FORMAT_SUFFIXES = {"png": ".png", "jpeg": ".jpg", "webp": ".webp", "tiff": ".tif"}
