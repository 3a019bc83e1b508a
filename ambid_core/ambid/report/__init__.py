"""The identification report: figures (:mod:`.figures`) and the HTML page (:mod:`.html`)."""
