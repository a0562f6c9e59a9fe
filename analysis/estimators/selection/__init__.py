"""Model-choice policy: which fitted model to believe, and whether any fits.

Goodness of fit of a model to the Allan deviation (:mod:`.adequacy`), the automatic choice of
the simplest model that fits (:mod:`.model_choice`), the reported coefficients with intervals
across candidates (:mod:`.coefficients`) and the screen that names channels with nothing to
characterise (:mod:`.screen`). The top wing: imports any other, none imports it.
"""
