"""Estimator messages in the words of the command line.

The estimators explain themselves in their own vocabulary: an argument of their Python API
(``fine_samples``) is what a library caller can change. A person reading ``analyze``'s text,
``export``'s warnings or a report runs the command line, where that argument does not exist;
:func:`user_text` puts in its place what that person can do (docs/noise-model.md names the
options). Machine-readable outputs (the JSON's ``message``) keep the estimator's words.
"""

from __future__ import annotations

import re

#: estimator advice naming an API argument -> what a command-line user can do instead
CLI_ADVICE = {
    # the fine-scale Allan variance is not white: a device filter the model lacks (composite.py)
    r"(?:give|raise) fine_samples": "add the device filter to the model (--model auto, or a model with +lp)",
}


def user_text(message: str) -> str:
    """``message`` with every API-argument advice of :data:`CLI_ADVICE` replaced by its command-line form."""
    for pattern, advice in CLI_ADVICE.items():
        message = re.sub(pattern, advice, message)
    return message
