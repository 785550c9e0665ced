"""Problem generators (domains) from the paper."""
