"""Images in: decoding (:mod:`.decode`), the object's mask in a photo (:mod:`.mask`) and framing
for the image encoder (:mod:`.frame`)."""
