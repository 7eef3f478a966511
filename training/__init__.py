"""Lightning training of the networks in ``models``: ``sonicskin train --config configs/train/<name>.yaml``."""
