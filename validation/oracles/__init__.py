"""Float64 and long-double oracles: independent reference answers that the
stability table and the tests judge the float32 renderer against. Each is
plain NumPy, written apart from the code it judges, and is itself checked
against closed forms and high-precision values (``tests/test_oracles.py``).
"""
