"""One router per resource: ``gimap`` (bake or serve a GI map), ``health``, ``stats``, ``scenes``."""
