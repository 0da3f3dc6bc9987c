"""The help text of FLAAIR's command lines: every option's default shown, examples as written.

`HelpFormatter` is the `formatter_class` of every `bin/flaair` command's parser (and of its
subcommands' parsers): the description and the epilog keep their line breaks (examples are
written pre-wrapped, each command line whole, a continuation indented under it), and each
option's help ends with its default unless the text already names it.
"""

from __future__ import annotations

import argparse

__all__ = ["HelpFormatter", "shows_default"]


def shows_default(text: str) -> bool:
    """Whether an option's help text already says its default (or that it is required)."""
    lowered = text.lower()
    return "default" in lowered or "%(default)" in text or "(required)" in lowered


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Description and epilog as written; every option's default shown.

    An option whose help already says its default is left as written. Otherwise the help gains
    "(default: X)": the value; "off" for a flag; "none" when the option is simply absent by
    default; "(required)" for a required option.
    """

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if action.help is argparse.SUPPRESS or not action.option_strings:
            return text
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            return text
        if shows_default(text):
            return text
        if action.required:
            return f"{text} (required)".strip()
        default = action.default
        if isinstance(action, argparse._StoreTrueAction) and default is False:
            shown = "off"
        elif isinstance(action, argparse._StoreFalseAction) and default is True:
            shown = "on"
        elif default is None or default == []:
            shown = "none"
        elif default is argparse.SUPPRESS:
            return text
        else:
            shown = "%(default)s"
        return f"{text} (default: {shown})".strip()
