"""SMPTE linear timecode (LTC): exact codec, sub-sample audio encoder and decoder, clock alignment and sync tables."""
