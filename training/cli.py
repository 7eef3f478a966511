"""``sonicskin train``: LightningCLI over SkinLitModule and SkinDataModule, configured by YAML."""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

from .data import SkinDataModule
from .module import SkinLitModule


class SkinCLI(LightningCLI):
    follow_root_dir = False  # --trainer.default_root_dir given without a logger: the logger writes there too

    def before_instantiate_classes(self) -> None:
        cfg = self.config.get(self.subcommand) if self.subcommand else self.config
        root, logger = cfg.trainer.default_root_dir, cfg.trainer.logger
        init = getattr(logger, "init_args", None)
        if self.follow_root_dir and root and init is not None and "save_dir" in init:
            init.save_dir = root

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.n_in", "model.n_in", apply_on="instantiate")
        parser.link_arguments("data.n_locations", "model.n_locations", apply_on="instantiate")
        parser.link_arguments("data.noise_db", "model.noise_db")


def main(args: list[str] | None = None, run: bool = True) -> SkinCLI:
    """``args`` as on the command line after ``sonicskin train`` (e.g. ``--config configs/train/moving.yaml``)."""
    given = [a.split("=", 1)[0] for a in (args or [])]
    cls = type("SkinCLI", (SkinCLI,), {"follow_root_dir": "--trainer.default_root_dir" in given
                                       and not any(a.startswith("--trainer.logger") for a in given)})
    return cls(SkinLitModule, SkinDataModule, args=["fit", *(args or [])] if run else args, run=run,
                   save_config_kwargs={"overwrite": True}, seed_everything_default=0)
