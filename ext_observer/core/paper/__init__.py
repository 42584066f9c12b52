"""
The paper's example on S³: the extended, plain and projected Luenberger-like
observers (``observer``), the simulated gyro (``gyro_model``) and the
experiments behind its figures and Table 1 (``experiments``).
"""
