"""The map service: versioned maps on disk (`store`), served on Zenoh (`server`), fetched and
cached by robots (`client`); chunked transfer with checksums (`transfer`), access rules (`access`)."""
