"""The LTC decoder: audio -> per-channel columns of frames (:func:`timecode.decode.decoder.decode_file`).

    decoder      files and sample arrays in, :class:`~timecode.decode.result.ChannelDecode` out
    edges        sub-sample edge times of square waves (droop compensated: droop)
    impulses     pole times of differentiated (impulse-train) LTC
    bits         edges -> bit cells and sync words
    bitclock     frame start times fitted on the bit clock
    continuity   labels that count, the frame rate they show
    assemble     frames and their columns from the edges
    result       the decoded columns (ChannelDecode, DecodedFrame, Reading, Extrapolated)
    formats      the columns as a table, CSV or JSON
"""
