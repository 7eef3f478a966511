"""Lightning training of the networks in ``models`` (the learned-model issue fills this package)."""
