"""
What writes this repository's generated docs: not installed with ext_observer.

The pages and figures of docs/ and the generated sections of docs/ and
config/, from the results the installed commands compute. A source tree
runs them through ``python -m ext_observer docs``, ``broad --docs`` and
``reproduce --docs`` (and ``python -m bench``); an installed package has
none of them.

- :mod:`~docgen.sections`: the one writer of a generated section between
  its two marker lines;
- :mod:`~docgen.parameter_tables`: docs/parameters.md's tables and the
  node sections of config/*.yaml, from the parameter specs;
- :mod:`~docgen.broad_page`, :mod:`~docgen.broad_plots`: docs/broad.md and
  its figures; :mod:`~docgen.robustness_page`: docs/robustness.md;
  :mod:`~docgen.covariance_page`: docs/covariance.md;
- :mod:`~docgen.reproduction_page`: docs/reproduction.md.
"""
