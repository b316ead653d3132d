"""The MQTT Sparkplug B edge node of a plant (``softplc mqtt``, its own process)."""
