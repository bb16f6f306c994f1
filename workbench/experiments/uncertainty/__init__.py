"""Issue 36's proof that the instrument's per-point uncertainty is honest (``workbench reproduce uncertainty``)."""
