model\.yaml:4:27: components\.me\.file: model `model\.yaml` .+ \[PHC\-E106\]
