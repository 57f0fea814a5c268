"""pyserial URL handlers of devices (pyserial finds `protocol_<scheme>` modules in the packages listed in
serial.protocol_handler_packages; importing `devices` adds this one): record:// and replay://, see
devices/recording.py."""
