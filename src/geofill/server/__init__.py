"""``geofill serve``: a web page to brush the hole and add reference photos, and the REST API behind it.

Needs the ``server`` extra (``pip install "geofill[server]"``)."""
