"""The wire: protocol, text mode, frames, decoder, unwrapping, telemetry, capture files, serial transport, ports."""
