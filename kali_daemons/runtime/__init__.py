"""What every process of an instance runs on: the config, the instance (arena, records,
semaphores), the one daemon base class, the flight recorder, the stall witness and the
instance's paths.
"""
