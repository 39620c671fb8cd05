"""Warnings a result carries to the terminal, the reports and the JSON (`warnings`: a list of objects with a
`code` and a `message`). A warning says what is doubtful about a result and what to change."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class ResultWarning:
    """`code`: a stable identifier (e.g. "ols_iv_disagree"); `message`: what is wrong and what to change."""

    code: str
    message: str

    def as_dict(self) -> dict[str, str]:
        """The JSON object: {"code": …, "message": …}."""
        return asdict(self)

    def __str__(self) -> str:
        return f"warning [{self.code}]: {self.message}"


def markdown_lines(warnings: list[ResultWarning]) -> list[str]:
    """A report's list of warnings, one Markdown item each ("- **code**: message"), or "- none"."""
    return [f"- **{w.code}**: {w.message}" for w in warnings] or ["- none"]
