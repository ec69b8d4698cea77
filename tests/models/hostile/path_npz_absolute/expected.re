model\.yaml:7:15: components\.lin\.matrices: matrices file .+ \[PHC\-E116\]
