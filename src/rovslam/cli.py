"""The `rovslam` command (placeholder until the CLI lands)."""


def main() -> None:  # pragma: no cover - replaced by the typer app
    raise SystemExit("rovslam: CLI not built yet")
