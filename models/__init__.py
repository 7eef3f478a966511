"""Torch networks over the OSPA-selected bins (the learned-model issue fills this package)."""
