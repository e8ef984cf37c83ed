"""The operator's tools: ``kalictl`` (``cli``), ``kalictl start``/``stop`` (``launcher``, with
``snapshot``), ``kalictl status`` (``introspect``) and ``kalictl top`` (``top``).
"""
