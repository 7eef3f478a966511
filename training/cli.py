"""``sonicskin train``: LightningCLI over SkinLitModule and SkinDataModule, configured by YAML."""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

from .data import SkinDataModule
from .module import SkinLitModule


class SkinCLI(LightningCLI):
    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.n_bins", "model.n_in")
        parser.link_arguments("data.n_locations", "model.n_locations", apply_on="instantiate")
        parser.link_arguments("data.noise_db", "model.noise_db")


def main(args: list[str] | None = None, run: bool = True) -> SkinCLI:
    """``args`` as on the command line after ``sonicskin train`` (e.g. ``--config configs/train/moving.yaml``)."""
    return SkinCLI(SkinLitModule, SkinDataModule, args=["fit", *(args or [])] if run else args, run=run,
                   save_config_kwargs={"overwrite": True}, seed_everything_default=0)
