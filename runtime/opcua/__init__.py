"""The OPC UA server (``softplc opcua PLANT``): its own process, fed by the controller."""
