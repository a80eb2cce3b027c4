"""Robot-program filters: every target of a robot program rewritten so that the real arm (its identified model)
goes where the program meant on the controller's model; everything else kept byte for byte.

One language-neutral core (:mod:`identify.programs.core`: targets with their spans in the text, what was not
rewritten and why, the rewrite itself), the compensation of the targets (:mod:`identify.programs.filter`) and
one module per language that finds the targets (:mod:`identify.programs.urscript`). Another language (KRL,
RAPID) is one more module with a ``parse`` and the formatting of its literals. Pure: no files, no devices.
"""
