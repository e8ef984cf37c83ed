"""Examples that ship with Kali: a servo plugin (``servo_plugin_example``) and a TG function
(``tg_function_example``), each one to copy.  The shipped cell (``config/default.yaml``)
names them as modules, so an installed Kali loads them as a checkout does."""
