import sys, numpy as np
def rd(p):
    f=open(p,'rb'); f.readline(); wh=f.readline().split(); f.readline()
    return np.frombuffer(f.read(),'<f4').reshape(int(wh[1]),int(wh[0]),3)[::-1].astype(np.float64)
a,b=rd(sys.argv[1]),rd(sys.argv[2])
w=np.array([0.2126,0.7152,0.0722])
m=(a+b)/2
la,lb,lm=(a*w).sum(-1),(b*w).sum(-1),(m*w).sum(-1)
mask=(la>0.02)&(lb>0.02)&(lm<5)
# chromaticity c = rgb / lum; its seed-to-seed difference is the coloured noise
ca=a[mask]/la[mask,None]; cb=b[mask]/lb[mask,None]
chroma=np.sqrt(((ca-cb)**2).mean()/2)
lum=np.sqrt((((la-lb)[mask]/lm[mask])**2).mean()/2)
print(f"chroma noise (rms of rgb/lum per seed) {chroma:.4f}, relative luminance noise {lum:.4f}, ratio {chroma/lum:.2f}")
